import sys, math, collections
sys.path.insert(0,__import__('os').path.dirname(__file__)); from ana_common import *
seq,out=sys.argv[1],sys.argv[2]; lvl=sys.argv[3] if len(sys.argv)>3 else 'all'
cam=load_cam(seq); FX,FY,CX,CY,BF=cam
gt=load_traj(f'{seq}/groundtruth.txt'); pts=load_dump(out)
S=[1.2**i for i in range(8)]
A=[[0,0],[0,0]]; bb=[0,0]; n=0; rs=[0,0]
for X,obs in pts:
    for a in obs:
        for b in obs:
            if a is b or a[4]<=0 or a[0] not in gt or b[0] not in gt: continue
            if lvl=='0' and (a[3] or b[3]): continue
            Rwa,Ca=gt[a[0]]; Rwb,Cb=gt[b[0]]
            ray=[(a[1]-CX)/FX,(a[2]-CY)/FY,1.0]
            rw=mv(Rwa,ray); rb=mtv(Rwb,rw)
            if rb[2]<=0.05: continue
            ur=(FX*rb[0]/rb[2]+CX, FY*rb[1]/rb[2]+CY)
            Xw=[Ca[i]+rw[i]*a[4] for i in range(3)]; xb=mtv(Rwb,[Xw[i]-Cb[i] for i in range(3)])
            if xb[2]<=0.05: continue
            up=(FX*xb[0]/xb[2]+CX, FY*xb[1]/xb[2]+CY)
            r=(b[1]-up[0], b[2]-up[1])
            if r[0]**2+r[1]**2>9: continue
            drot=(ur[0]-a[1], ur[1]-a[2]); dpar=(up[0]-ur[0], up[1]-ur[1])
            w=1/S[b[3]]**2
            for i,(p,q) in enumerate([(drot,drot),(drot,dpar),(dpar,dpar)]):
                pass
            A[0][0]+=w*(drot[0]**2+drot[1]**2); A[0][1]+=w*(drot[0]*dpar[0]+drot[1]*dpar[1]); A[1][1]+=w*(dpar[0]**2+dpar[1]**2)
            bb[0]+=w*(r[0]*drot[0]+r[1]*drot[1]); bb[1]+=w*(r[0]*dpar[0]+r[1]*dpar[1]); n+=1
            rs[0]+=r[0]; rs[1]+=r[1]
A[1][0]=A[0][1]
sol=solve(A,bb)
print('%s levels=%s n=%d: observed-GT residual = alpha*rotational_flow + beta*parallax_flow: alpha %.5f beta %.5f; mean residual (%.3f, %.3f) px'%(out,lvl,n,sol[0],sol[1],rs[0]/n,rs[1]/n))
