import sys, math
sys.path.insert(0,__import__('os').path.dirname(__file__)); from ana_common import *
seq,out,f=sys.argv[1],sys.argv[2],sys.argv[3]
gt=load_traj(f'{seq}/groundtruth.txt'); est=load_traj(f'{out}/{f}')
ks=sorted(k for k in est if k in gt); step=int(sys.argv[4]) if len(sys.argv)>4 else 1
def rel(T,a,b):
    Ra,Ca=T[a]; Rb,Cb=T[b]
    return mtv(Ra,[Cb[i]-Ca[i] for i in range(3)]), matmul(transpose(Ra),Rb)
def ang(R): return math.acos(max(-1,min(1,(R[0][0]+R[1][1]+R[2][2]-1)/2)))
line=[]
tot=[0,0,0,0]
for i in range(0,len(ks)-step,step):
    a,b=ks[i],ks[i+step]
    te,Re=rel(est,a,b); tg,Rg=rel(gt,a,b)
    tot[0]+=dot(te,tg)/norm(tg); tot[1]+=norm(tg); tot[2]+=ang(Re); tot[3]+=ang(Rg)
    line.append('%.3f'%(dot(te,tg)/norm(tg)**2) if norm(tg)>0.02 else '  -  ')
print(' '.join(line))
print('total: translation (est projected on gt) / gt = %.5f ; rotation angle est/gt = %.5f'%(tot[0]/tot[1], tot[2]/tot[3]))
